"""A complete run's SHA-256 kept beside its file (labctl/run/digest.py): ``labctl run`` writes it as ``sha256sum``
does, an evaluation takes it while the file is no newer, and hashes the file itself once it is."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess

import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from labctl.run.digest import digest_path, kept_digest, write_digest


@pytest.fixture
def recorded(tmp_path, write_campaign, small_model):
    out = tmp_path / "r.h5"
    with pytest.raises(SystemExit) as code:
        main(["run", str(write_campaign()), "--sim", "--model", str(small_model()), "-o", str(out), "--quiet"])
    assert code.value.code == 0
    return out


def test_a_complete_run_keeps_its_hash_as_sha256sum_writes_it(recorded):
    truth = hashlib.sha256(recorded.read_bytes()).hexdigest()
    assert digest_path(recorded).read_text() == f"{truth}  r.h5\n"
    assert kept_digest(recorded) == truth
    if shutil.which("sha256sum"):
        check = subprocess.run(["sha256sum", "-c", digest_path(recorded).name], cwd=recorded.parent,
                               capture_output=True, text=True)
        assert check.returncode == 0 and check.stdout == "r.h5: OK\n"


def test_an_evaluation_takes_the_kept_hash_and_hashes_a_file_changed_since(recorded):
    truth = hashlib.sha256(recorded.read_bytes()).hexdigest()
    kept = digest_path(recorded)
    kept.write_text(f"{'0' * 64}  r.h5\n")  # not the file's: an evaluation that states it took it unread
    assert evaluate_runs([recorded]).conditions[0]["sha256"] == "0" * 64
    stat = kept.stat()
    os.utime(recorded, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))  # the run file changed after its hash
    assert kept_digest(recorded) is None
    assert evaluate_runs([recorded]).conditions[0]["sha256"] == truth


@pytest.mark.parametrize("text", ["", "abc  r.h5\n", f"{'a' * 64}  other.h5\n", f"{'A' * 64}  r.h5\n"])
def test_a_kept_hash_of_another_form_or_file_is_not_taken(tmp_path, text):
    run = tmp_path / "r.h5"
    run.write_bytes(b"run")
    digest_path(run).write_text(text)
    assert kept_digest(run) is None
    assert write_digest(run) == kept_digest(run) == hashlib.sha256(b"run").hexdigest()
