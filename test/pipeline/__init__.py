"""Tests of eit_skin.pipeline."""
