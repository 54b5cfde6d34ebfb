"""``sensaov view``: live inspection, the stages wired for one viewpoint at a time and served.

The buffer and the scene are loaded once (``session``); each request names a camera and a
channel (``query``), is traced through primary visibility, painted and encoded as bytes
(``inspection``), and answered by the standard library's HTTP server (``server``) to the
self-contained page (``page.html``).
"""
