"""Files online-id reads and writes: the track-run CSV (``tracklog``)."""
