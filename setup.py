"""Only what pyproject.toml cannot say: the folders mapped into the vts_hw package, and every
package under each, found rather than listed (pyproject's packages.find would name the packages
under drivers/ "drivers...", not "vts_hw.drivers..."; docs/decisions/0045-installed-as-users-install-it.md).
Everything else (metadata, dependencies, package data) is in pyproject.toml."""

from setuptools import find_packages, setup

PACKAGE_DIR = {
    "vts_hw": "vts_hw",
    "vts_hw.drivers": "drivers",
    "vts_hw.procedures": "procedures",
    "vts_hw.sim_devices": "sim_devices",
}

setup(
    package_dir=PACKAGE_DIR,
    packages=[
        f"{name}.{sub}" if sub else name for name, folder in PACKAGE_DIR.items() for sub in ["", *find_packages(folder)]
    ],
)
