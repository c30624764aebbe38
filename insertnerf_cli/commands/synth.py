"""`insertnerf synth` (being built)."""
import click


@click.command("synth")
def synth() -> None:
    """Not built yet."""
    raise click.ClickException("insertnerf synth is not built yet in this version.")
