"""Eyelid rig: blend shapes for up- and down-looking lids, and eye-region landmarks.

``lids``       the pitch-to-weight rule, the lid blend shapes (with inbetweens) and their checks
``landmarks``  the 12 eyelid landmarks per eye, a curve that deforms with the lid shapes
"""
