"""Output-only identification: modes from the response alone, scaled by the cutting-force model.

Modules: :mod:`.harmonics` (milling lines found and regressed out of the response), :mod:`.ssi`
(covariance-driven SSI, stabilisation and clustering), :mod:`.ml` (Whittle-ML refinement of SSI's
modes; :mod:`.whittle` its likelihood, :mod:`.blocks` the bins pooled where a band holds many,
:mod:`._ml_fit` one group's fit, :mod:`._ml_inference` its standard errors and evidence),
:mod:`.modes` (the chain with its intervals), :mod:`.uncertainty`, :mod:`.scaling` (OMAH with the
force model's tooth lines), :mod:`.background` (scale from the background force's level),
:mod:`.identify` (records in, ``robomill-modal/1`` model out).
"""
