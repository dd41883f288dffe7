"""Tests of eit_skin.touch."""
