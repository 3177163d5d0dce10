"""Map the repository's top-level folders onto the installed `magline` namespace.

The design card keeps `core/`, `plugins/` and `stations/` at the repository root, but nothing named
bare `core` or `plugins` may land in site-packages.  setuptools' ``package_dir`` does the renaming;
the package list is computed so a new sub-package cannot be forgotten.
"""

from setuptools import find_packages, setup

ROOTS = {"core": "magline.core", "plugin": "magline.plugin", "plugins": "magline.plugins", "sim": "magline.sim",
         "sitl": "magline.sitl", "stations": "magline.stations", "testing": "magline.testing"}

packages = []
package_dir = {}
for folder, installed in ROOTS.items():
    package_dir[installed] = folder
    packages.append(installed)
    packages += [f"{installed}.{sub}" for sub in find_packages(where=folder)]

setup(
    packages=packages,
    package_dir=package_dir,
    package_data={"magline.stations": ["*.yaml"], "magline.core.operator_ui.screen": ["static/*"],
                  "magline.core.dashboard": ["static/*"]},
)
