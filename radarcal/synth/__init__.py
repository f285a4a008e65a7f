"""Ground-truth scene generators (``radarcal synth ...``)."""
