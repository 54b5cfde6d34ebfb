"""sensaov's benchmark suite: ``make bench`` (``python -m bench``) measures the paper's claims.

Every comparison is a ratio of two measurements taken side by side (interleaved A, B, A, B) in
one run, with warm kernel caches and synchronised timings. See ``bench/README.md``.
"""
