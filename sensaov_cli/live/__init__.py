"""``sensaov view``: live inspection, the stages wired for one viewpoint at a time and served.

The buffer and the scene are loaded once (``session``, which also reads each request's camera
and channel), traced through primary visibility, painted and encoded as bytes (``inspection``),
and answered by the standard library's HTTP server (``server``) to the self-contained page
(``page.html``).
"""
