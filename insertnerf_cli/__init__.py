"""insertnerf: novel-view synthesis from a folder of images with a pretrained generalizable NeRF."""

__version__ = "0.1.0"
