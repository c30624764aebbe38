"""`insertnerf poses` (being built)."""
import click


@click.command("poses")
def poses() -> None:
    """Not built yet."""
    raise click.ClickException("insertnerf poses is not built yet in this version.")
