"""Click commands, one module each; COMMANDS is what group.py registers (on first use)."""
from insertnerf_cli.cli.commands.common import user_errors  # noqa: F401  (re-exported for the command modules)
from insertnerf_cli.cli.commands.eval import eval_command
from insertnerf_cli.cli.commands.finetune import finetune_command
from insertnerf_cli.cli.commands.poses import poses
from insertnerf_cli.cli.commands.render import render
from insertnerf_cli.cli.commands.synth import synth
from insertnerf_cli.cli.commands.train import train

COMMANDS = [poses, synth, train, render, eval_command, finetune_command]
