"""Click commands, one module each; COMMANDS is what group.py registers (on first use)."""
from .common import user_errors  # noqa: F401  (re-exported for the command modules)
from .poses import poses
from .synth import synth
from .train import train
from .render import render
from .eval import eval_command
from .finetune import finetune_command

COMMANDS = [poses, synth, train, render, eval_command, finetune_command]
