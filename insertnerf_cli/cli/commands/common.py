"""Options and error handling shared by the commands."""
from __future__ import annotations

import errno
import functools
import math
from typing import Any, Callable

import click

from insertnerf_cli.errors import INTERRUPTED, INTERRUPTED_EXIT_CODE, UserError, os_error_message


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a UserError or an OSError (permission denied, disk full, read-only, ...) into a one-line click error
    (exit 1), and Ctrl-C into a short message (exit 130). Any other exception is a bug and keeps its traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except UserError as err:
            raise click.ClickException(str(err)) from None
        except OSError as err:
            if err.errno == errno.EPIPE:
                raise  # output piped into e.g. `head`: click quietly handles a closed pipe
            raise click.ClickException(os_error_message(err)) from None
        except KeyboardInterrupt:
            click.echo(INTERRUPTED, err=True)
            raise SystemExit(INTERRUPTED_EXIT_CODE) from None

    return wrapper


class FiniteFloat(click.FloatRange):
    """A float option that also refuses nan and inf (click's FloatRange lets both through its bounds)."""

    name = "finite float"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number


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
