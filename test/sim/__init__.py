"""Tests of eit_skin.sim."""
