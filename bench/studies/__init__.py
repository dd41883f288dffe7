"""One-off studies: a design question measured once, kept with its answer (the .md beside
the script) so that it can be rerun when the question comes back."""
