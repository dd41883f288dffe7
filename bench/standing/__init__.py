"""Standing benchmarks: rerun for every report; each writes its result file beside it
(bench/REPORT.md is their index)."""
