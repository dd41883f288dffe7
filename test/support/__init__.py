"""Helpers the tests share (no tests here): patience, patch copies, phantoms, peers."""
