"""Depth priors per training view (``eve3d stereo-depth``): one ``{view}.npz`` per view with
``depth`` (camera z, 0 = invalid), ``confidence`` (M^c in [0,1]) and ``normal`` (camera
space, unit, facing the camera), each with a PNG preview."""
