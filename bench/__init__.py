"""Benchmarks run by ``make bench``: each ``bench_*`` module has ``main()`` printing its figures."""
