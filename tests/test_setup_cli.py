"""Set-up and the command line as a new user meets them (issue 14, "Set-up, CLI and devices"):
the documents point only at files in the repository; the install script skips an unchanged
install; shutdown prints no leak dump; devices that cannot be opened are named at start-up."""

from __future__ import annotations

import glob
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from waiting import wait_until

ROOT = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------ the documents' paths

_TICKED = re.compile(r"`([^`\n]+)`")
_LINK = re.compile(r"\]\(([^)\s#]+)[^)]*\)")
_PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.\w+)?$")  # NAME.toml, SCRIPT.py: any file there


def _tracked_tops() -> set[str]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return {line.split("/", 1)[0] for line in out.splitlines()}


def mentioned_paths(text: str, tops: set[str]) -> list[str]:
    """Relative paths a document mentions: markdown link targets, and words in code spans that
    start in one of the repository's top-level entries (or go up or sideways with ../ or ./)."""
    found = [t for t in _LINK.findall(text) if "://" not in t and not t.startswith("mailto:")]
    for span in _TICKED.findall(text):
        for word in span.split():
            word = word.rstrip(".,;:)")
            if "/" not in word or word.startswith("/"):
                continue
            if word.startswith(("../", "./")) or word.split("/", 1)[0] in tops:
                found.append(word)
    return found


def _exists(rel: str) -> bool:
    target = (ROOT / rel).resolve()
    if not target.is_relative_to(ROOT):
        return False  # outside the repository: a fresh clone does not have it
    parts = [("*" + m.group(1) if m.group(1) else "*") if (m := _PLACEHOLDER.match(p)) else p
             for p in target.relative_to(ROOT).parts]
    pattern = str(ROOT.joinpath(*parts)) if parts else str(ROOT)
    if glob.glob(pattern):
        return True
    # Made at run time (var/, tests/artifacts/): ignored by git on purpose, so it is named, not shipped.
    # A folder keeps its trailing "/": a "dir/" pattern matches a folder that is not there yet only so.
    name = str(target) + ("/" if rel.endswith("/") else "")
    return subprocess.run(["git", "check-ignore", "-q", name], cwd=ROOT).returncode == 0


@pytest.mark.parametrize("doc", ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))])
def test_documents_point_only_at_files_in_the_repository(doc: str) -> None:
    text = (ROOT / doc).read_text()
    paths = mentioned_paths(text, _tracked_tops())
    assert doc != "README.md" or len(paths) >= 30, paths  # the extraction found the paths it should check
    missing = sorted({p for p in paths if not _exists(p)})
    assert missing == [], f"{doc} mentions paths that are not in the repository: {missing}"


def test_readme_points_at_the_design_document() -> None:
    assert "docs/design.md" in mentioned_paths((ROOT / "README.md").read_text(), _tracked_tops())


def test_path_check_catches_a_path_outside_the_repository() -> None:
    paths = mentioned_paths("See `../shared/DESIGN.md` and [x](docs/nope.md), `configs/robots/NAME.toml`.",
                            _tracked_tops())
    assert paths == ["docs/nope.md", "../shared/DESIGN.md", "configs/robots/NAME.toml"]
    assert [_exists(p) for p in paths] == [False, False, True]


# ------------------------------------------------------------------------------ scripts/install

# A stand-in for python (a real full install takes ~1.5 min and the network: .ci/run does that on a
# fresh clone). "-m venv DIR" makes DIR/bin/python (a copy of this script); "-m pip" runs are logged;
# PIP_FAIL=1 makes every other call fail like a broken download.
FAKE_PYTHON = """#!/bin/sh
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then mkdir -p "$3/bin" && cp "$0" "$3/bin/python" && exit 0; fi
[ "$1" = "-m" ] && [ "$2" = "pip" ] && echo "$*" >> "$PIP_LOG"  # the pip runs, not the kernel warm-up
[ "${PIP_FAIL:-0}" = 1 ] && exit 1
exit 0
"""


@pytest.fixture
def project(tmp_path: Path) -> Path:
    """The install script and pyproject.toml in a directory of their own."""
    (tmp_path / "scripts").mkdir()
    (tmp_path / "scripts" / "install").write_text((ROOT / "scripts" / "install").read_text())
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    (tmp_path / "constraints.txt").write_text((ROOT / "constraints.txt").read_text())
    fake = tmp_path / "fake-python"
    fake.write_text(FAKE_PYTHON)
    fake.chmod(0o755)
    return tmp_path


def install(project: Path, *args: str, fail: bool = False) -> tuple[int, list[str], str]:
    """Run scripts/install; the pip runs it made, and its stderr."""
    log = project / "pip.log"
    log.write_text("")
    env = {"PATH": "/usr/bin:/bin", "PYTHON": str(project / "fake-python"), "PIP_LOG": str(log),
           "PIP_FAIL": "1" if fail else "0"}
    r = subprocess.run(["bash", "scripts/install", *args], cwd=project, env=env, capture_output=True, text=True,
                       timeout=60)
    return r.returncode, log.read_text().splitlines(), r.stderr


def test_install_skips_pip_when_nothing_changed(project: Path) -> None:
    code, pips, _ = install(project)
    assert code == 0
    assert len(pips) == 2 and "--upgrade pip" in pips[0] and pips[1].endswith("-e .")  # a fresh .venv
    assert all(" -q " in p for p in pips)  # pip stays quiet
    code, pips, err = install(project)
    assert code == 0 and pips == [] and err == ""  # unchanged: no pip at all
    # The test extras are more: installed once, and they cover a plain run afterwards.
    assert install(project, "--test")[1][-1].endswith("-e .[test]")
    assert install(project)[1] == [] and install(project, "--test")[1] == []


@pytest.mark.parametrize("changed", ["pyproject.toml", "constraints.txt"])
def test_install_runs_pip_again_when_pyproject_or_the_constraints_change(project: Path, changed: str) -> None:
    install(project)
    with (project / changed).open("a") as f:
        f.write("\n# a new dependency, or a version moved\n")
    code, pips, _ = install(project)
    assert code == 0 and len(pips) == 1 and pips[0].endswith("-e .")  # the venv stays, the package is reinstalled
    assert install(project)[1] == []


def test_install_stays_within_the_tested_versions(project: Path) -> None:
    pips = install(project, "--test")[1]
    assert pips[-1].endswith("-c constraints.txt -e .[test]"), pips


def test_the_tested_versions_are_within_pyprojects_ranges_and_cover_every_dependency() -> None:
    """constraints.txt pins one version of each package, inside pyproject.toml's range for it, and leaves
    none of the run or test dependencies to chance."""
    import tomllib

    from packaging.requirements import Requirement

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    lines = [x for x in (ROOT / "constraints.txt").read_text().splitlines() if x.strip() and not x.startswith("#")]
    assert all("==" in x for x in lines), "one exact version per line"
    pins = {re.sub(r"[-_.]+", "-", name).lower(): version.strip() for name, _, version in
            (x.partition("==") for x in lines)}
    assert len(pins) == len(lines), "one line per package"
    for spec in [*project["dependencies"], *project["optional-dependencies"]["test"]]:
        req = Requirement(spec)
        name = re.sub(r"[-_.]+", "-", req.name).lower()
        assert name in pins, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"constraints.txt pins {req.name}=={pins[name]}, outside pyproject.toml's {req.specifier}")


def test_a_failed_install_is_retried_and_a_new_venv_installs(project: Path) -> None:
    install(project)
    (project / "pyproject.toml").write_text((project / "pyproject.toml").read_text() + "\n# changed\n")
    code, pips, _ = install(project, fail=True)
    assert code != 0 and len(pips) == 1
    assert len(install(project)[1]) == 1  # the failure left no stamp: the next run tries again
    shutil.rmtree(project / ".venv")  # a fresh machine
    assert len(install(project)[1]) == 2


def test_a_venv_with_mujoco_4s_split_loses_it_before_the_install(project: Path) -> None:
    install(project)
    site = project / ".venv" / "lib" / "python3.11" / "site-packages"
    (site / "mujoco_core-4.0.0.dist-info").mkdir(parents=True)  # what pip left of mujoco 4.0.0 (split in three)
    (project / "pyproject.toml").write_text((project / "pyproject.toml").read_text() + "\n# changed\n")
    code, pips, _ = install(project)
    assert code == 0 and len(pips) == 2, pips
    assert pips[0].endswith("-m pip uninstall -q -y mujoco mujoco-core mujoco-studio") and pips[1].endswith("-e .")
    shutil.rmtree(site / "mujoco_core-4.0.0.dist-info")  # (the uninstall's doing, in a real venv)
    (project / "pyproject.toml").write_text((project / "pyproject.toml").read_text() + "\n# changed again\n")
    assert install(project)[1] == [pips[1]]  # without the split: no uninstall


# ------------------------------------------------------ `servo-app run`: devices, Ctrl-C, shutdown

TOKEN = "setup-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}

MISSING_DEVICES = """
[adapters.spacenav]
type = "spacenav"
socket = "{tmp}/spnav.sock"

[adapters.distance]
type = "serial_line"
port = "{tmp}/ttyUSB-missing"
[adapters.distance.fields.distance]
pattern = 'D=([-+0-9.eE]+)'

[adapters.ft_can]
type = "can"
interface = "socketcan"
channel = "srvtst0"
[[adapters.ft_can.layout]]
id = 0x2B0
name = "Distance"
[adapters.ft_can.layout.signals.distance]
start = 0
size = 2
signed = false
byte_order = "little"

[[applications]]
name = "teleop"
type = "teleop"
sources = {{ twist = "spacenav" }}
priority = 30
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Service:
    """`servo-app run` in a process of its own, on a free port, with its own var directory."""

    def __init__(self, tmp: Path, *args: str) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.proc = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(self.port),
                                      "--var-dir", str(tmp / "var"), "--token", TOKEN, *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def wait_healthy(self, timeout: float = 60.0) -> None:
        def up() -> bool:
            assert self.proc.poll() is None, self.proc.communicate()
            try:
                return httpx.get(f"{self.base}/api/health", timeout=2).status_code == 200
            except httpx.TransportError:
                return False

        wait_until(up, timeout)

    def stop(self) -> tuple[int, str, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            out, err = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
            raise AssertionError(f"servo-app run did not stop on SIGINT within 30 s:\n{out}\n{err}") from None
        return self.proc.returncode, out, err


@pytest.mark.e2e
def test_devices_that_cannot_be_opened_are_named_at_start_up_with_the_fix(tmp_path: Path) -> None:
    cfg = tmp_path / "inputs.toml"
    cfg.write_text(MISSING_DEVICES.format(tmp=tmp_path))
    svc = Service(tmp_path, "--inputs", str(cfg))
    try:
        svc.wait_healthy()
        with httpx.Client(base_url=svc.base, timeout=10) as c:
            rows = {r["name"]: r for r in c.get("/api/inputs").json()["sources"]}
            spnav, serial, can = rows["spacenav"]["failure"], rows["distance"]["failure"], rows["ft_can"]["failure"]
            assert spnav["device"] == f"spacenavd's socket {tmp_path}/spnav.sock"
            assert "spacenavd is not running" in spnav["reason"] and "systemctl start spacenavd" in spnav["fix"]
            assert serial["device"] == f"serial port {tmp_path}/ttyUSB-missing"
            assert "not plugged in" in serial["reason"] and "/dev/serial/by-id" in serial["fix"]
            assert can["device"] == "CAN interface srvtst0 (socketcan)"
            assert "ip link set srvtst0 up type can" in can["fix"]  # no SocketCAN here, or no such interface
            # The console polls the state: the failure is in its summary too.
            summary = {s["name"]: s for s in c.get("/api/state").json()["inputs"]["sources"]}
            assert summary["spacenav"]["failure"]["device"] == spnav["device"]
            # Enabling goes ahead (other sources may command) and says which source cannot, and why.
            lease = c.post("/api/lease", json={"client": "setup-test"}, headers=AUTH).json()["lease_id"]
            r = c.post("/api/inputs/enable", json={"enable": True}, headers={**AUTH, "X-Lease-Id": lease})
            assert r.status_code == 200, r.text
            detail = r.json()["detail"]
            assert {f["name"] for f in detail["failed_sources"]} == {"spacenav", "distance", "ft_can"}
            assert "input source 'spacenav' (used by 'teleop') cannot command: spacenavd's socket" in detail["warning"]
    finally:
        code, _, err = svc.stop()
    assert code == 0, err
    lines = [ln for ln in err.splitlines() if "cannot be opened" in ln]
    assert len(lines) == 3, err
    assert any(f"input 'spacenav' (spacenav) cannot be opened: spacenavd's socket {tmp_path}/spnav.sock" in ln
               and "Fix: install and start spacenavd" in ln for ln in lines), lines
    assert any(f"serial port {tmp_path}/ttyUSB-missing" in ln and "Fix: plug it in" in ln for ln in lines), lines
    assert any("CAN interface srvtst0 (socketcan)" in ln and "Fix: " in ln for ln in lines), lines


@pytest.mark.e2e
def test_shutdown_after_a_stream_with_inputs_prints_no_leak_dump(tmp_path: Path) -> None:
    """A Ctrl-C after a session with an inputs file: the servo process (which reads the input slot
    after each IK solve) exits with no "nanobind: leaked instances" dump of ruckig objects."""
    cfg = tmp_path / "inputs.toml"
    cfg.write_text(MISSING_DEVICES.format(tmp=tmp_path))
    svc = Service(tmp_path, "--inputs", str(cfg))
    try:
        svc.wait_healthy()
        with httpx.Client(base_url=svc.base, timeout=10) as c:
            lease = c.post("/api/lease", json={"client": "setup-test"}, headers=AUTH).json()["lease_id"]
            hdr = {**AUTH, "X-Lease-Id": lease}
            assert c.post("/api/session/start", headers=hdr).status_code == 200
            wait_until(lambda: c.get("/api/state").json()["state"] == "streaming", 30)
            assert c.post("/api/jog", json={"linear": [10, 0, 0], "angular": [0, 0, 0]}, headers=hdr).status_code == 200
    finally:
        code, out, err = svc.stop()
    assert code == 0, err
    assert "servo_app: stopped; stream ended" in out, out
    assert "leaked" not in err, err


@pytest.mark.e2e
def test_ctrl_c_during_start_up_stops_the_service(tmp_path: Path) -> None:
    """SIGINT as soon as the service prints its address (before the HTTP server has installed its own
    handlers) stops it; it used to be swallowed and the service kept running."""
    svc = Service(tmp_path)
    assert svc.proc.stdout is not None
    line = svc.proc.stdout.readline()
    assert "console http://" in line, line
    svc.proc.send_signal(signal.SIGINT)
    try:
        out, err = svc.proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        svc.proc.kill()
        svc.proc.communicate()
        raise AssertionError("SIGINT during start-up was lost: the service kept running") from None
    assert svc.proc.returncode == 0, err
    assert "servo_app: stopped" in out, out


@pytest.mark.parametrize(("argv", "words"), [
    # Ran on serving nothing (uvicorn's bind failed unreported) until killed.
    (["--http-port", "70000"], ["--http-port", "70000", "0..65535"]),
    # Tracebacks, exit 1, after a servo process had been started (and advice to POST /api/reset).
    (["--lead", "9"], ["--lead", "9", "0..8"]),
    # Not settable before; a stall time below the idle Janome loop's publish gap ended it needlessly.
    (["--servo-stall-s", "0.1"], ["--servo-stall-s", "'0.1'", "at least 0.5", "stalled"]),
    (["--servo-stall-s", "nan"], ["--servo-stall-s", "'nan'", "number of seconds"]),
    (["--servo-stall-s", "soon"], ["--servo-stall-s", "'soon'", "number of seconds"]),
    (["--robot", "fanuc:127.0.0.1:99999"], ["--robot='fanuc:127.0.0.1:99999'", "99999", "0..65535"]),
    # Tracebacks, exit 1.
    (["--robot", "kuka"], ["--robot='kuka'", "unknown robot backend", "fanuc"]),
    (["--model", "nosuch"], ["'nosuch'", "unknown", "lrmate200id"]),
    (["--var-dir", "{file}"], ["--var-dir=", "not-a-directory", "cannot be used"]),  # a traceback after start-up
])
def test_bad_run_options_exit_2_naming_the_option_and_value(tmp_path: Path, argv: list[str],
                                                             words: list[str]) -> None:
    a_file = tmp_path / "not-a-directory"
    a_file.write_text("")
    argv = [a.format(file=a_file) for a in argv]
    cmd = [sys.executable, "-m", "servo_app.cli", "run", "--var-dir", str(tmp_path / "var"), "--token", TOKEN, *argv]
    try:
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"still running after 60 s: {exc.stdout!r} {exc.stderr!r}") from None
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "console http://" not in r.stdout, r.stderr
    for w in words:
        assert w in r.stderr, (w, r.stderr)
