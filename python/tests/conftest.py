"""Shared fixtures: the Python own-loop example and the Rust example's recording."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent  # python/tests -> repository root


def load_example(name: str):
    """Imports python/examples/NAME.py as a module."""
    path = HERE.parent / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"gpm_example_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def read_diagnostics(path):
    """Every /diagnostics message of an MCAP file, with the /config message, via the Python
    `mcap` reader (independent of gpm)."""
    from mcap.reader import make_reader

    steps, config = [], None
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic == "/diagnostics":
                steps.append(json.loads(message.data))
            elif channel.topic == "/config":
                config = json.loads(message.data)
    return config, steps


@pytest.fixture(scope="session")
def rust_own_loop(tmp_path_factory):
    """The recording of gpm's Rust example `examples/own_loop.rs` (`--out DIR`): the file named
    by GPM_RUST_OWN_LOOP_MCAP (CI sets it), else one made here with cargo from the repository
    this package sits in; skipped when neither is available."""
    given = os.environ.get("GPM_RUST_OWN_LOOP_MCAP")
    if given:
        return Path(given)
    if shutil.which("cargo") is None or not (REPO / "examples" / "own_loop.rs").exists():
        pytest.skip("no Rust reference: set GPM_RUST_OWN_LOOP_MCAP or run from the gpm repository")
    out = tmp_path_factory.mktemp("rust_own_loop")
    subprocess.run(
        ["cargo", "run", "--release", "--quiet", "--example", "own_loop", "--", "--out", str(out)],
        cwd=REPO,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return out / "run.mcap"
