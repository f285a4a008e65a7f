"""Camera intrinsics from chessboard / ChArUco views: ``detect`` (corners), ``select`` (coverage, novelty),
``solve`` (models, outlier rejection, σ, projection uncertainty), ``crossval`` (split halves, model choice),
``stereo`` (T_cam1_cam0), ``pipeline`` (screening + solve), ``collect`` (files, videos, parallel detection),
``session`` (the session file). Corner-level scenes with known truth are in ``radarcal.synth.intrinsics_views``.
See docs/intrinsics.md."""
