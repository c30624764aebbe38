"""What `render` and `eval` write: the run records (records.py), frames, depth maps, videos and cameras.json
(outputs.py), eval's side-by-sides (eval_outputs.py), the fused point cloud (pointcloud.py) and the HTML pages
(report/)."""
