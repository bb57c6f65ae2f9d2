"""pytest plugin of the test kit (entry point ``pytest11``); filled in by the test-kit work."""
