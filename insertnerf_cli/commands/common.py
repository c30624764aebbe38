"""Options and error handling shared by the commands."""
from __future__ import annotations

import functools
from typing import Any, Callable

import click

from ..errors import UserError


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a UserError into a one-line click error (exit 1), and Ctrl-C into a short message (exit 130)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except UserError as err:
            raise click.ClickException(str(err)) from None
        except KeyboardInterrupt:
            click.echo("Interrupted; finished outputs were kept, re-run the same command to continue.", err=True)
            raise SystemExit(130) from None

    return wrapper


def device_option(func: Callable[..., Any]) -> Callable[..., Any]:
    return click.option("--device", type=click.Choice(["auto", "cpu", "cuda"]), default="auto", show_default=True,
                        help="Where to run the network; auto picks CUDA when available.")(func)


def overwrite_option(func: Callable[..., Any]) -> Callable[..., Any]:
    return click.option("--overwrite", is_flag=True, help="Replace existing outputs instead of refusing.")(func)


def resolve_device(name: str) -> "torch.device":  # noqa: F821
    """Resolve --device once, here; library code takes the device from its inputs."""
    import torch

    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda was asked for but PyTorch sees no CUDA GPU; use --device cpu.")
    return torch.device(name)
