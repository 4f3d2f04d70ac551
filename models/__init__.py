"""Physics effects and feed-drive twin, physics baselines, shallow network and trainers, discovery."""
