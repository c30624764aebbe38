"""Camera poses from a folder of photos with pycolmap (`insertnerf poses`): the input images and output folder
(folder.py), SIFT matching (matching.py), incremental mapping and the re-mapping of a folded walk (estimate.py,
reconstruction.py), a two-view consistency check (check.py) and the preview point clouds (preview.py)."""
