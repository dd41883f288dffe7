"""Standing benchmarks: rerun for every report; each writes its result file beside it
(bench/standing/reconstruction.md is their index)."""
