"""The example third-party distribution (examples/acme-magline) installed as an outside author
would: magline from its wheel (not editable, not this checkout's tests) and the example into a
clean virtual environment, then the example's own tests, written only with magline.testing."""

from __future__ import annotations

import shutil
import subprocess
import sys

from conftest import REPO

EXAMPLE = REPO / "examples" / "acme-magline"
NOT_SOURCE = shutil.ignore_patterns(".venv", ".git", "build", "dist", "*.egg-info", "__pycache__", "*.sqlite",
                                    "*.json", "examples")


def run(*command, cwd=None) -> str:
    done = subprocess.run([str(c) for c in command], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{' '.join(map(str, command))} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


def test_the_example_plugin_from_a_clean_venv_passes_its_own_tests(tmp_path):
    source = tmp_path / "magline-src"  # a copy: building never writes into the checkout
    shutil.copytree(REPO, source, ignore=NOT_SOURCE)
    run(sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", tmp_path / "dist",
        source)
    wheel, = (tmp_path / "dist").glob("magline-*.whl")
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", venv)
    python = venv / "bin" / "python"
    run(python, "-m", "pip", "install", "-q", wheel, f"{shutil.copytree(EXAMPLE, tmp_path / 'acme')}[test]")
    where = run(python, "-c", "import magline.core, magline.testing, acme_magline; print(magline.core.__file__)")
    assert "site-packages" in where and str(REPO) not in where  # the installed wheel, not this checkout
    out = run(python, "-m", "pytest", "-q", "-p", "no:cacheprovider", tmp_path / "acme" / "tests", cwd=tmp_path)
    assert "4 passed" in out
    plugins = run(venv / "bin" / "magline", "plugins")
    assert '"acme"' in plugins and '"acme-magline"' in plugins  # registered, and by which distribution
