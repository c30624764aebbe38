"""The `insertnerf` command group. Each command lives in insertnerf_cli/commands/<name>.py and stays thin:
check input -> build config -> call one library function -> print a one-line summary."""
from __future__ import annotations

import click

from . import __version__
from .commands import COMMANDS


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="insertnerf")
def cli() -> None:
    """Novel views, depth maps and videos from a folder of photos, with a pretrained generalizable NeRF.

    \b
    Typical use:
      insertnerf poses photos/ --out scene/      # camera poses with COLMAP (pycolmap)
      insertnerf render scene/ --out views/      # frames, depth maps and a turntable video
    """


for _command in COMMANDS:
    cli.add_command(_command)


def main() -> None:
    cli(prog_name="insertnerf")
