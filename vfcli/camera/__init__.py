"""The camera: orthographic projection (camera), rasterisation (raster), simulated silhouettes
(silhouette) and the pose of the model in the image (pose)."""
