"""Reproduce the paper's model numbers: the ~30 arcsec worked example of section 1.2 and the
K_HSE / lambda2 / C23 relation of section 3, with the symbolic model and the closed forms.

Run: python studies/paper_model.py
"""
from hse_opt.model.paper import reproduce, summary

n = reproduce()
print("\n".join(summary(n)))

# the paper's certified numbers
assert 28.0 < n.example_amplitude_model < 34.0, "worked example should give about 30 arcsec"
assert abs(n.example_amplitude_model - n.example_amplitude_eq14) < 0.05
assert abs(n.k_hse_model_arcsec_per_radps - 17.4) < 0.01
assert 150.0 < n.c23_implied_arcsec < 180.0
print("OK: paper numbers reproduced")
