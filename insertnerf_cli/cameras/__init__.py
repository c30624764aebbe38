"""Cameras and rays: the one camera type (OpenCV camera-to-world, pinhole intrinsics; camera.py) and the rays
through its pixels (rays.py). Every other stage builds on these; conventions in docs/conventions.md."""
