"""Fine-tuning the generator on one scene's own photos (`insertnerf finetune`, `render --finetune M`).

``finetune(scene_dir, out, FinetuneConfig, device) -> FinetuneResult``; the views `eval` holds out are never used.
"""
from insertnerf_cli.finetune.loop import FinetuneConfig, FinetuneResult, Progress, check_out_file, finetune
from insertnerf_cli.finetune.render_cache import cached_finetune

__all__ = ["FinetuneConfig", "FinetuneResult", "Progress", "cached_finetune", "check_out_file", "finetune"]
