"""Tests of eit_skin.ros."""
