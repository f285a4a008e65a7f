"""Camera pose on the field from clicked landmarks (``field_pnp``) and the localisation error it implies (``error_map``)."""
