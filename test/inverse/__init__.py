"""Tests of eit_skin.inverse."""
