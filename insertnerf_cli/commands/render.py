"""`insertnerf render` (being built)."""
import click


@click.command("render")
def render() -> None:
    """Not built yet."""
    raise click.ClickException("insertnerf render is not built yet in this version.")
