"""Test-time optimisation (paper, Sec. 3.2): one engine (:mod:`.engine`: the step loop, stop
rules, best snapshot, the candidate race, texture seeding) that the single-frame fit
(:mod:`.frame`) and the window fit (:mod:`.window`, with its path fit in :mod:`.path` and its
spin search in :mod:`.spin`) both run."""
