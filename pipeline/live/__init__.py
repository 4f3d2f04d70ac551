"""``watch``: samples from a live controller feed into each machine axis's daily lost motion
(docs/watch.md). ``config`` reads WATCH.toml, ``feed`` turns channel updates into samples and
days, ``sources`` speaks the protocols, ``loop`` runs them."""
