"""The `insertnerf` command group. Each command lives in insertnerf_cli/cli/commands/<name>.py and stays thin:
check input -> build config -> call one library function -> print a one-line summary.

The commands (and torch behind them) are imported when click first looks one up, with Ctrl-C held meanwhile
(see interrupts.held_interrupts), so `insertnerf --version` is instant and an interrupted start-up exits cleanly.
"""
from __future__ import annotations

import click

from insertnerf_cli import __version__
from insertnerf_cli.interrupts import held_interrupts


class _Commands(click.Group):
    """The command group, registering the commands of insertnerf_cli.cli.commands on first use."""

    def _load(self) -> None:
        if self.commands:
            return
        with held_interrupts():
            from insertnerf_cli.cli.commands import COMMANDS
        for command in COMMANDS:
            self.add_command(command)

    def list_commands(self, ctx: click.Context) -> list[str]:
        self._load()
        return super().list_commands(ctx)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        self._load()
        return super().get_command(ctx, cmd_name)


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="insertnerf")
def cli() -> None:
    """Novel views, depth maps and videos from a folder of photos, with a pretrained generalizable NeRF.

    \b
    Typical use:
      insertnerf poses photos/ --out scene/      # camera poses with COLMAP (pycolmap)
      insertnerf render scene/ --out views/      # frames, depth maps and a turntable video
    """
