"""Rendering a camera from its nearest reference views: the render path's options (options.py), the chunked
image renderer with its shortcuts (image_renderer.py), the per-frame driver that picks references, caches their
encodings and builds the prior and occlusion maps (view_renderer.py), the blend at the prior (prior_blend.py), and
the camera paths `render` follows (camera_paths.py)."""
