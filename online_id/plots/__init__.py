"""Figures. Each function takes computed result objects and draws them; matplotlib is imported only here."""
