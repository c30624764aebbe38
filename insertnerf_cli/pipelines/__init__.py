"""The libraries behind `insertnerf render` (render.py, with its inputs: posing unposed photos, fine-tuning
first; inputs.py) and `insertnerf eval` (evaluate.py). No click here: the commands in cli/ are thin wrappers."""
