"""The experiment store: one HDF5 file per recording; the only package that imports h5py."""
