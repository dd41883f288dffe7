"""Tests of eit_skin.cli."""
