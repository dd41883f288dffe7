"""The repository as a whole: layout, style, installed package, examples, benchmarks."""
