"""Package layout that pyproject.toml cannot express: the repository's ``scenes/`` directory ships as package data.

``scenes/`` stays where the README's commands look for it (``springsim run scenes/cloth_64.yaml``); the
build maps it to ``springsim/scene/data/``, where an installed springsim finds its scenes by name
(``springsim run cloth_64``, ``springsim scenes``; :mod:`springsim.scene.shipped`). Everything else is in
pyproject.toml.
"""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["springsim", "springsim.*"]) + ["springsim.scene.data"],
    package_dir={"springsim.scene.data": "scenes"},
    package_data={"springsim": ["py.typed"], "springsim.scene.data": ["*.yaml"]},
)
