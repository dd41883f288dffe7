"""ament_python package eit_skin (messages live in the nested msg/ package)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "eit_skin"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={f"{PACKAGE}.design": ["static/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml"))),
    ],
    # Versions are pinned in requirements.txt (pip machines) or come from
    # rosdep (robots); setup.py names only what must be importable.
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="eit_skin maintainers",
    maintainer_email="eit-skin@example.org",
    description="Robot skin by Electrical Impedance Tomography.",
    license="Apache-2.0",
    extras_require={"test": ["pytest"]},
    entry_points={
        "console_scripts": [
            "eit-skin = eit_skin.cli.main:main",
            "eit_driver = eit_skin.ros.entry:driver",
            "eit_reconstruction = eit_skin.ros.entry:reconstruction",
            "eit_classifier = eit_skin.ros.entry:classifier",
        ],
    },
)
