"""Tests of eit_skin.io."""
