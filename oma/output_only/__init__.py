"""Output-only identification: modes from the response alone, scaled by the cutting-force model.

Modules: :mod:`.harmonics` (milling lines found and regressed out of the response), :mod:`.ssi`
(covariance-driven SSI, stabilisation and clustering), :mod:`.modes` (the chain with jackknife
intervals), :mod:`.uncertainty`, :mod:`.scaling` (OMAH with the force model's tooth lines),
:mod:`.identify` (records in, ``robomill-modal/1`` model out), :mod:`.shared` (where the shared
real data live).
"""
