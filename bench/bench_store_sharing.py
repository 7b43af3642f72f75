"""## The store as other tools see it (issue 18)

1. Which groups of a store xarray opens with named dimensions: from the store file with the
   h5netcdf and netcdf4 engines, and through ``vfcli.store.open_dataset``.
2. h5py reading 12-bit video frame by frame: N-bit (the default for a 12-bit MRAW) against
   gzip (what `vfcli share` writes), 100 frames of 512 x 512 (a smooth image plus noise of
   30 counts); file sizes.
3. The cost of a stage's content digest (hashing its stored bytes when the stage is written),
   per stage of the store.

Reproduce::

    .venv/bin/python bench/bench_store_sharing.py STORE     # e.g. demo/recording.h5
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import h5py
import numpy as np

from vfcli.store import Store, open_dataset
from vfcli.store.parts import own_parts
from vfcli.store.provenance import content_digest


def _opens(name: str, opener) -> bool:  # noqa: ANN001
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with opener() as ds:
                return not [d for d in ds.dims if str(d).startswith("phony_dim")]
    except Exception as exc:  # noqa: BLE001 - reporting which group fails is the point
        print(f"    {name:<20} FAILS: {type(exc).__name__}: {str(exc)[:90]}")
        return False


def groups_xarray_opens(store: Path) -> None:
    """Every group of the store file (those in part files included) opened three ways: the store
    file with the h5netcdf engine and with the netcdf4 engine (when netCDF4 is installed), and
    vfcli.store.open_dataset (h5netcdf, from the file that holds the group)."""
    import xarray as xr

    names: list[str] = []
    with h5py.File(store, "r") as f:  # the links to the part files included
        f.visititems_links(lambda n, _link: names.append(n) if isinstance(f[n], h5py.Group) else None)
    ways = {
        "xr.open_dataset(store, group, engine='h5netcdf')":
            lambda n: (lambda: xr.open_dataset(store, group=n, engine="h5netcdf")),
        "vfcli.store.open_dataset(store, group)": lambda n: (lambda: open_dataset(store, n)),
    }
    try:
        import netCDF4  # noqa: F401
        ways["xr.open_dataset(store, group, engine='netcdf4')"] = \
            lambda n: (lambda: xr.open_dataset(store, group=n, engine="netcdf4"))
    except ImportError:
        print("  (netCDF4 is not installed: the netcdf4 engine is not measured)")
    for way, opener in ways.items():
        ok = sum(_opens(n, opener(n)) for n in names)
        print(f"  {way}: opens {ok} of {len(names)} groups with named dimensions")


def nbit_vs_gzip_reads(n: int = 100) -> None:
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:512, 0:512]
    base = 2000 + 1000 * np.sin(x / 40) * np.cos(y / 50)
    frames = np.clip(base[None] + rng.normal(0, 30, (n, 512, 512)), 0, 4095).astype(np.uint16)
    with tempfile.TemporaryDirectory() as d:
        per_frame = {}
        for c in ("nbit", "gzip"):
            path = Path(d) / f"{c}.h5"
            with Store(path).write("bench") as w, w.stage("hsc", config_json="{}") as s:
                s.write_frames("frames", frames.shape, np.uint16, (frames[a:a + 16] for a in range(0, n, 16)),
                               compression=c)
            with h5py.File(path, "r") as f:
                ds = f["hsc/frames"]
                t = time.perf_counter()
                for i in range(n):
                    ds[i]
                per_frame[c] = (time.perf_counter() - t) / n
            size = os.path.getsize(path) + sum(p.stat().st_size for p in own_parts(path))  # the video is in a part file
            print(f"  {c:<5} h5py {per_frame[c] * 1e3:6.1f} ms per 512 x 512 frame, store {size / 1e6:.1f} MB")
        print(f"N-bit reads {per_frame['nbit'] / per_frame['gzip']:.1f}x slower than gzip in h5py")


def digest_cost(store: Path) -> None:
    with h5py.File(store, "r") as f:  # the stages in part files through their links
        for name in ("hsc", "ldv", "sync", "flow", "fields", "mesh"):
            if name in f:
                size = sum(ds.id.get_storage_size() for ds in f[name].values() if isinstance(ds, h5py.Dataset))
                t = time.perf_counter()
                content_digest(f[name])
                dt = time.perf_counter() - t
                print(f"  /{name:<7} {size / 1e6:7.1f} MB stored, content digest {dt * 1e3:6.0f} ms")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print("usage: bench_store_sharing.py STORE (e.g. demo/recording.h5)", file=sys.stderr)
        sys.exit(2)
    store = Path(sys.argv[1])
    groups_xarray_opens(store)
    nbit_vs_gzip_reads()
    digest_cost(store)
