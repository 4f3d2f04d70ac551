"""Named physical effects and the feed-drive twin that measures itself like a laser.

The twin's presets are campaign files shipped as data, ``experiments/presets/<name>.toml``
(read by ``models.physics.campaign.load_config``); ``PRESETS`` maps their names to the files.

The product's own files (presets, example data, the hidden-effect scenarios) are found in
``SHIPPED``, beside the installed packages: never by importing the name ``experiments`` nor
from the working folder, where a user's own ``experiments/`` folder would stand in for them.
"""

from pathlib import Path

SHIPPED = Path(__file__).resolve().parents[2] / "experiments"
"""The product's ``experiments`` folder as installed (a sibling of ``models/``, in a checkout,
an editable install and a wheel alike)."""


def preset_files() -> dict[str, Path]:
    """The shipped twin presets by name, in name order."""
    folder = SHIPPED / "presets"
    return {p.stem: p for p in sorted(folder.iterdir(), key=lambda p: p.name)
            if p.suffix == ".toml" and p.is_file()}


PRESETS = preset_files()
