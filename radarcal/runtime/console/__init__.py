"""Browser pages for the operator: the live console of ``radarcal run --ui`` (:mod:`.live`) on a small standard-library
server with server-sent events, a per-run token and loopback binding (:mod:`.server`). Assets in ``static/``."""
