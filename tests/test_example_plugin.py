"""The example third-party distribution (examples/acme-magline) installed as an outside author
would: magline from its wheel (not editable, not this checkout's tests) and the example into a
clean virtual environment, then the example's own tests, written only with magline.testing.

The libraries both need (numpy, scipy, pluggy, …) come from this test environment's site-packages,
seen through a folder of links that leaves magline's own editable install out, and ``pip check``
proves that the wheels' declared requirements are met by them.  Why: resolving and unpacking them
into the new environment again took 30 of the test's 40 s, and the suite has a time budget; what the
test is about — the wheel installed, not the checkout; the plugin registered through its entry
point; its tests written against the public face — stays proven."""

from __future__ import annotations

import shutil
import site
import subprocess
import sys
from pathlib import Path

from conftest import REPO, source_copy

EXAMPLE = REPO / "examples" / "acme-magline"


def run(*command, cwd=None) -> str:
    done = subprocess.run([str(c) for c in command], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{' '.join(map(str, command))} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


def shared_libraries(folder):
    """A folder of links to this environment's installed libraries, magline's own install left out."""
    folder.mkdir()
    for location in site.getsitepackages():
        for entry in sorted(Path(location).iterdir()):
            if "magline" in entry.name.lower() or entry.suffix == ".pth" or (folder / entry.name).exists():
                continue
            (folder / entry.name).symlink_to(entry)
    return folder


def test_the_example_plugin_from_a_clean_venv_passes_its_own_tests(tmp_path):
    source = source_copy(tmp_path / "magline-src")  # a copy: building never writes into the checkout
    run(sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", tmp_path / "dist",
        source)
    wheel, = (tmp_path / "dist").glob("magline-*.whl")
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", "--without-pip", venv)
    python = venv / "bin" / "python"
    target_site = run(python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").strip()
    (Path(target_site) / "shared-libraries.pth").write_text(
        f"{shared_libraries(tmp_path / 'libraries')}\n", encoding="utf-8")
    pip = (sys.executable, "-m", "pip", "--python", python)
    run(*pip, "install", "-q", "--no-deps", "--no-build-isolation", wheel,
        f"{shutil.copytree(EXAMPLE, tmp_path / 'acme')}[test]")
    run(*pip, "check")  # every requirement of the two wheels (magline's, the example's, [test]'s) is met
    where = run(python, "-c", "import magline.core, magline.testing, acme_magline; print(magline.core.__file__)")
    assert "site-packages" in where and str(REPO) not in where  # the installed wheel, not this checkout
    out = run(python, "-m", "pytest", "-q", "-p", "no:cacheprovider", tmp_path / "acme" / "tests", cwd=tmp_path)
    assert "11 passed" in out
    plugins = run(venv / "bin" / "magline", "plugins")
    assert '"acme"' in plugins and '"acme-magline"' in plugins  # registered, and by which distribution
    # registered by place: listing (as every command's start) imports the plugin's modules, not its driver or sink
    probe = ("import contextlib, io, sys\nsys.argv = ['magline', 'plugins']\nfrom magline.core.entry import main\n"
             "with contextlib.redirect_stdout(io.StringIO()):\n    main()\n"
             "print(' '.join(sorted(m for m in sys.modules if m.startswith('acme_magline'))))")
    assert run(python, "-c", probe).split() == ["acme_magline", "acme_magline.feed", "acme_magline.plugin"]
