"""Tests of eit_skin.fem."""
