"""The kernels' disk cache follows every kernel source (servo_app/jit.py): a kernel whose callee in
another module changed is compiled afresh, in a new process, not loaded with the old callee."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from servo_app import jit

_CALLEE = """\
from servo_app.jit import kernel


@kernel("float64(float64)")
def f(x):
    return x + {step}
"""

_CALLER = """\
from pkg.callee import f
from servo_app.jit import kernel


@kernel("float64(float64)")
def g(x):
    return f(x) * 10.0
"""

# pkg's kernels cache by the digest of pkg's own two sources, as servo_app's do by theirs.
_INIT = """\
from pathlib import Path

from servo_app.jit import use_cache_for

HERE = Path(__file__).parent
CACHE = use_cache_for([HERE / "callee.py", HERE / "caller.py"], HERE.parent / "cache")
"""

_RUN = """\
import json
import pkg
from pkg.caller import g
print(json.dumps({"g": g(1.0), "hits": sum(g.stats.cache_hits.values()), "cache": str(pkg.CACHE)}))
"""


def _run(root: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", _RUN], cwd=root, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_kernel_whose_callee_changed_in_another_module_is_compiled_afresh(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(_INIT)
    (pkg / "callee.py").write_text(_CALLEE.format(step=1.0))
    (pkg / "caller.py").write_text(_CALLER)

    first = _run(tmp_path)
    assert first["g"] == 20.0 and first["hits"] == 0  # compiled, and saved
    again = _run(tmp_path)
    assert again == {**first, "hits": 1}  # loaded from the disk cache, not compiled again

    (pkg / "callee.py").write_text(_CALLEE.format(step=2.0))  # the caller's file is untouched
    changed = _run(tmp_path)
    assert changed["g"] == 30.0, changed  # numba alone (cache beside the caller) gave the old 20.0
    assert changed["hits"] == 0 and changed["cache"] != first["cache"]


def test_every_module_with_a_kernel_is_a_kernel_source() -> None:
    root = Path(jit.__file__).resolve().parent
    with_kernels = {
        "servo_app." + ".".join(path.relative_to(root).with_suffix("").parts)
        for path in root.rglob("*.py") if re.search(r"^@kernel\(", path.read_text(encoding="utf-8"), re.M)
    }
    assert with_kernels, "no kernel found: the scan is wrong"
    assert with_kernels <= set(jit.KERNEL_MODULES) <= set(jit.KERNEL_SOURCES)
    for module in jit.KERNEL_SOURCES:
        assert jit.source_path(module).is_file(), module


def test_this_process_caches_by_the_digest_of_every_kernel_source() -> None:
    import numba

    digest = jit.source_digest(jit.source_path(m) for m in jit.KERNEL_SOURCES)
    assert jit.CACHE_DIR.name == "servo_app-" + digest
    assert str(jit.CACHE_DIR) == numba.config.CACHE_DIR


def test_the_digest_changes_with_any_byte_or_name_and_only_then(tmp_path: Path) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("x = 1\n")
    b.write_text("y = 2\n")
    base = jit.source_digest([a, b])
    assert jit.source_digest([a, b]) == base
    b.write_text("y = 3\n")
    assert jit.source_digest([a, b]) != base
    b.write_text("y = 2\n")
    assert jit.source_digest([a, b]) == base
    c = tmp_path / "c.py"
    c.write_text("y = 2\n")
    assert jit.source_digest([a, c]) != base  # same bytes, another file
    # File boundaries count: "x = 1\ny" + " = 2\n" is not "x = 1\n" + "y = 2\n".
    a.write_text("x = 1\ny")
    b.write_text(" = 2\n")
    assert jit.source_digest([a, b]) != base


def test_the_install_warm_up_removes_older_caches_only(tmp_path: Path) -> None:
    keep = tmp_path / "servo_app-0000000000000000"
    old = tmp_path / "servo_app-1111111111111111"
    other = tmp_path / "someone-elses"
    for d in (keep, old, other):
        (d / "sub").mkdir(parents=True)
    assert jit.prune_caches(tmp_path, keep) == [old]
    assert keep.is_dir() and other.is_dir() and not old.exists()


@pytest.mark.parametrize("user_dir", ["", "/some/where"])
def test_a_user_cache_directory_is_respected(user_dir: str) -> None:
    base = jit.cache_base(user_dir or None)
    if user_dir:
        assert base == Path(user_dir)
    else:
        assert base.is_dir()


def test_the_warm_up_command_names_its_cache(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "servo_app.jit", "-v"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    assert str(jit.CACHE_DIR) in out.stderr, textwrap.shorten(out.stderr, 400)
