"""Steps several jobs share, below the workflows: a workflow imports steps, ``features`` and
``models``, never another workflow (``tests/test_layers.py`` checks it)."""
