"""`insertnerf eval` (being built)."""
import click


@click.command("eval")
def eval_command() -> None:
    """Not built yet."""
    raise click.ClickException("insertnerf eval is not built yet in this version.")
