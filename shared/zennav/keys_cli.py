"""`zennav keys DIR`: a new Ed25519 key pair for signing parameter sets (zennav.learn.signing)."""
from __future__ import annotations

import click


@click.command("keys")
@click.argument("directory", type=click.Path(file_okay=False))
def keys_cmd(directory):
    """Write a new parameter-set signing key pair to DIRECTORY: paramset-signing.pem (private, mode 0600: the
    trainer's --signing-key, its host only) and paramset-verify.pem (public: every predictor's --verify-key).
    Refuses to overwrite an existing private key."""
    from .learn.signing import generate

    try:
        private, public = generate(directory)
    except FileExistsError as e:
        raise click.ClickException(f"{e.filename} exists; remove it first to make a new pair") from None
    except OSError as e:
        raise click.ClickException(f"{directory}: {e.strerror or e}") from None
    click.echo(f"signing key (trainer --signing-key): {private}\nverify key (predictor --verify-key): {public}")
