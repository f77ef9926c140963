"""Both codecs decode every shared vector to exactly the expected canonical JSON (SPEC.md §9)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from icgt.protocol.runner import run as run_python

ROOT = Path(__file__).resolve().parents[2]
VECTORS = sorted((ROOT / "protocol" / "vectors").glob("*/*.bin"))


def test_there_is_a_vector_for_every_message_and_every_rejection_rule() -> None:
    from icgt.protocol.messages import MESSAGE_TYPES

    text = "".join(p.with_suffix(".json").read_text() for p in VECTORS)
    for cls in MESSAGE_TYPES.values():
        assert f'"type":"{cls.NAME}"' in text, cls.NAME
    for counter in (
        "oversized",
        "cobs_error",
        "truncated",
        "crc_error",
        "wrong_version",
        "unknown_type",
        "bad_length",
        "seq_gaps",
        "seq_resets",
        "pending_bytes",
    ):
        assert f'"{counter}":0' in text and f'"{counter}":' in text.replace(f'"{counter}":0', ""), counter


@pytest.mark.parametrize("vector", VECTORS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_python_runner_matches_expected(vector: Path) -> None:
    assert run_python(vector) == vector.with_suffix(".json").read_text().strip()


@pytest.mark.parametrize("vector", VECTORS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_cpp_runner_matches_expected(vector: Path, cpp_vector_runner: Path) -> None:
    out = subprocess.run([cpp_vector_runner, vector], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == vector.with_suffix(".json").read_text().strip()


def test_python_runner_is_a_command() -> None:
    vector = ROOT / "protocol" / "vectors" / "valid" / "ping_typical.bin"
    out = subprocess.run(
        [sys.executable, "-m", "icgt.protocol.runner", str(vector)], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == vector.with_suffix(".json").read_text().strip()


def test_generated_code_and_vectors_are_fresh() -> None:
    gen = subprocess.run([sys.executable, ROOT / "protocol" / "generate.py", "--check"], capture_output=True, text=True)
    assert gen.returncode == 0, gen.stderr
    vec = subprocess.run(
        [sys.executable, ROOT / "protocol" / "make_vectors.py", "--verify"], capture_output=True, text=True
    )
    assert vec.returncode == 0, vec.stderr
