"""The sample stream every source yields: :class:`~online_id.stream.samples.Sample` in canonical channel
names and SI units (``samples``), and how a stream with lost samples is recognised and bridged (``gaps``)."""
