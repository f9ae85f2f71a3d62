"""Board conformance tests: the same tests against every board target (see conftest.py)."""
