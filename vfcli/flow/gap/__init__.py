"""The glottal gap: detection (detect), the rays and their outermost silhouette (rays), the opening
function and the measured silhouettes (opening), sub-pixel edges (subpixel/)."""
