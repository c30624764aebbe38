"""Structure-from-motion points at known poses and what the renderer makes of them: points triangulated at the
scene's own poses where it has none (triangulate.py, epipolar.py), a frame's depth prior (depth_prior.py) and each
reference view's occlusion map (occlusion_maps.py)."""
