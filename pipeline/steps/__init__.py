"""Steps several jobs share, below the workflows: a workflow imports steps, ``features`` and
``models``, never another workflow (``tests/test_layers.py`` checks it), and a step never
imports the workflows, neither a job nor the package's records (``tests/test_architecture.py``
checks it)."""
