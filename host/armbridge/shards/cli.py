"""The --ray, --workers and --checkpoint options of the sharded commands, defined once.

Used by `armbridge train smm-3r|smm-4r|smm-7r|masr-iknn` and `armbridge bench masr-plan|smm|wjrrt`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from armbridge.shards.engine import Runner, reachable

RAY_HELP = ("Run the shards on a running Ray cluster: auto (the one this machine joined with `ray start`) "
            "or the head's address HOST:PORT (docs/cluster.md). Needs the ray extra.")
WORKERS_HELP = ("Without --ray: 1 runs the shards here, one after the other; N > 1 starts a Ray of N CPUs "
                "on this machine.")


def ray_option() -> Any:
    return typer.Option(None, "--ray", help=RAY_HELP)


def workers_option() -> Any:
    return typer.Option(1, "--workers", help=WORKERS_HELP)


def checkpoint_option(default: str) -> Any:
    return typer.Option(None, "--checkpoint",
                        help=f"Folder where every finished shard is written; a rerun with the same settings resumes "
                             f"from it [default: {default}].")


def runner(ray: Optional[str], workers: int, checkpoint: Optional[Path], progress: bool = True) -> Runner:
    """The Runner of the options (Runner checks them); a head address that does not answer is an
    error before any work starts."""
    out = Runner(ray=ray, workers=workers, checkpoint=checkpoint, progress=progress)
    if ray is not None and ray != "auto":
        reachable(ray)
    return out
