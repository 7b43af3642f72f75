"""The camera: orthographic projection, rasterisation, silhouettes and the pose of the model in the image."""
