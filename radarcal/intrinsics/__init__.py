"""Camera intrinsics from chessboard / ChArUco views: ``detect`` (corners), ``select`` (coverage, novelty),
``solve`` (models, outlier rejection, σ, projection uncertainty), ``crossval`` (split halves, model choice),
``stereo`` (T_cam1_cam0), ``pipeline`` (screening + solve), ``collect`` (files, videos, parallel detection),
``simulate`` (corner-level scenes with known truth). See docs/intrinsics.md."""
