"""i2pbench reference plugin: VP2P-Match (Zhou et al., NeurIPS 2023), the authors' network in `official/`."""
