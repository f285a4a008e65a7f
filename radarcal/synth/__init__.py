"""Ground-truth scene generators (data in users' formats + truth.json)."""
