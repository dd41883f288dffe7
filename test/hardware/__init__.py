"""Tests of eit_skin.hardware."""
