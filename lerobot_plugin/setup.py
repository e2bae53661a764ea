"""The plugin's dependencies, computed at build time: gazereg comes from the checkout this folder sits in.

`pip install ./lerobot_plugin` (from a gazereg checkout) then installs gazereg's core from that checkout with its
own dependencies (tyro, ...; torch, numpy and accelerate already come with lerobot, within gazereg's ranges), so
the `gazereg` commands the README documents work in the LeRobot environment. A copy of this folder outside a
gazereg checkout depends on `gazereg` by name: install gazereg first (`pip install /path/to/gazereg`).
"""

from pathlib import Path

from setuptools import setup

LEROBOT = "lerobot[smolvla,pi,dataset]>=0.6,<0.7"


def gazereg_requirement() -> str:
    checkout = Path(__file__).resolve().parent.parent
    pyproject = checkout / "pyproject.toml"
    if pyproject.is_file() and 'name = "gazereg"' in pyproject.read_text():
        return f"gazereg @ {checkout.as_uri()}"
    return "gazereg"


setup(install_requires=[LEROBOT, gazereg_requirement()])
