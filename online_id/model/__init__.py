"""The lateral model as pure functions (``lateral``) and its exact discretisation (``discretise``).

A new unmodelled effect (issue: gap diagnosis) goes in its own module here as an
extension of these functions, never as a change to their signatures.
"""
