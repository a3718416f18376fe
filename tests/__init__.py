"""The pytest suite (a package, so that ``tests.doubles`` imports the same way from tests and tooling)."""
