"""eit_skin's benchmarks (not installed): ``standing`` (rerun for every report), ``studies``
(one-off questions kept with their answers), ``stress`` (long and hostile runs) and
``header``, the first line every report starts with. Run them from the repository root as
modules: ``.venv/bin/python -m bench.standing.bench_skin``."""
