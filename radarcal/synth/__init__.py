"""Ground-truth scene generators (``radarcal synth <scene>``): data in users' formats plus ``truth.json``."""
