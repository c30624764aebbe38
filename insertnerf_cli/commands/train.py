"""`insertnerf train` (being built)."""
import click


@click.command("train")
def train() -> None:
    """Not built yet."""
    raise click.ClickException("insertnerf train is not built yet in this version.")
