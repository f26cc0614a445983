"""Shared pytest configuration. Fixtures for one device live beside that device's tests or in tests/fakes/."""
