"""pvtflow: the one import package its distribution installs, so that no other distribution's names collide.

Installed, everything is below it: ``pvtflow.planner``, ``pvtflow.axes``, ``pvtflow.service`` and the shipped data,
``pvtflow.configs`` (pyproject's package-dir maps the repository's top-level folders there). In a source tree
(``PYTHONPATH=<clone>``, pytest in a clone, bench/) those folders are this folder's siblings: the package looks for
its subpackages there too, so that a clone runs its own code whatever else is installed.
"""

from pathlib import Path

_HERE = Path(__file__).resolve().parent
if not (_HERE / "configs").is_dir():  # a source tree: the subpackages are the repository's top-level folders
    __path__.append(str(_HERE.parent))
