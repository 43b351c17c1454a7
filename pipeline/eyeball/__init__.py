"""The parametric eyeball (paper section 3.1): geometry, blend shapes, landmarks, textures."""
