"""Schemathesis (``st run``) against the service as users run it: ``servo-app run`` in a process of its
own with its embedded simulator, HTTP on loopback. Generated valid and invalid requests on every
operation of the OpenAPI document, with the token and the control lease (tests/fuzz_hooks.py), must find
no server error and no answer the document does not describe (status code, content type, body schema).

Bounded: ``FUZZ_MAX_EXAMPLES`` cases per operation and phase (default 30), one pass of each phase.
``FUZZ_MAX_TIME=<s>`` turns the run into a soak: schemathesis 4 then repeats the fuzzing phase with new
cases until that budget is spent (a time to spend, not a ceiling).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(900)]

TOKEN = "fuzz-token-0123456789"
ROOT = Path(__file__).resolve().parents[1]
CHECKS = "not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def service(tmp_path: Path) -> Iterator[str]:
    """``servo-app run`` on a free port; yields its base URL; stopped with SIGINT (exit code 0)."""
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(port), "--var-dir", str(tmp_path),
         "--token", TOKEN, "--api-priority", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    base_url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, f"servo-app run exited {proc.returncode}"
            try:
                if httpx.get(f"{base_url}/api/health", timeout=2.0).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "servo-app run did not answer /api/health"
            time.sleep(0.05)
        yield base_url
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        out = proc.stdout.read() if proc.stdout else ""
    assert proc.returncode == 0, out


def test_every_operation_answers_as_documented(service: str, tmp_path: Path) -> None:
    st = Path(sys.executable).with_name("st")
    env = {**os.environ, "SCHEMATHESIS_HOOKS": "tests.fuzz_hooks", "FUZZ_BASE_URL": service, "FUZZ_TOKEN": TOKEN,
           "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    cmd = [str(st), "run", f"{service}/openapi.json", "--checks", CHECKS, "--workers", "1",
           "--max-examples", os.environ.get("FUZZ_MAX_EXAMPLES", "30"), "--seed", "14", "--no-color",
           "--phases", "examples,coverage,fuzzing", "--request-timeout", "15",
           # The header parameters (X-Lease-Id) are replaced by the hooks: most generated ones are filtered.
           "--suppress-health-check", "filter_too_much",
           "--report", "junit,ndjson", "--report-dir", str(tmp_path / "report")]
    # No --max-time by default: schemathesis 4 spends all of it, re-running the fuzzing phase in cycles
    # (181 s, 4,901 cases, 171 s of them fuzzing). One pass is what this test promises: each operation's
    # coverage cases (boundary and invalid values of every parameter and body field) and up to 30
    # generated cases, ~1,400 in all, ~22 s. A soak sets FUZZ_MAX_TIME.
    if os.environ.get("FUZZ_MAX_TIME"):
        cmd += ["--max-time", os.environ["FUZZ_MAX_TIME"]]
    run = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    (tmp_path / "st.out").write_text(run.stdout + run.stderr)
    if os.environ.get("FUZZ_OUT"):
        Path(os.environ["FUZZ_OUT"]).write_text(run.stdout + run.stderr)
    assert run.returncode == 0, run.stdout[-20000:] + run.stderr[-5000:]
    # Every documented operation went through both generating phases, none skipped or filtered away.
    spec = httpx.get(f"{service}/openapi.json", timeout=10.0).json()
    operations = {f"{method.upper()} {path}" for path, item in spec["paths"].items()
                  for method in item if method in {"get", "put", "post", "delete", "patch"}}
    done: dict[str, set[str]] = {}
    for events in (tmp_path / "report").glob("*.ndjson"):
        for line in events.read_text().splitlines():
            finished = json.loads(line).get("ScenarioFinished")
            if finished and finished["status"] == "success" and finished["recorder"]["cases"]:
                done.setdefault(finished["phase"], set()).add(finished["recorder"]["label"])
    assert operations and done.get("coverage") == operations and done.get("fuzzing") == operations, done
    # Whatever was asked, the service made the controller post no alarm (warnings aside).
    history = httpx.get(f"{service}/api/state", timeout=10.0).json().get("alarm_history", [])
    assert [a for a in history if not a.get("warning")] == [], history
