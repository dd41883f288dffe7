"""Tests of eit_skin.design."""
