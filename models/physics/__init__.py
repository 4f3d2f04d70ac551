"""Named physical effects and the feed-drive twin that measures itself like a laser.

The twin's presets are campaign files shipped as data, ``experiments/presets/<name>.toml``
(read by ``models.physics.campaign.load_config``); ``PRESETS`` maps their names to the files.
"""

from importlib import resources
from pathlib import Path


def preset_files() -> dict[str, Path]:
    """The shipped twin presets by name, in name order."""
    folder = resources.files("experiments").joinpath("presets")
    return {Path(p.name).stem: Path(str(p)) for p in sorted(folder.iterdir(), key=lambda p: p.name)
            if p.name.endswith(".toml")}


PRESETS = preset_files()
