"""Tests of eit_skin.patch."""
