"""Sizes and filters: the sizes users ask for, the classic filters and the reference maps, every
map resized by what it holds."""
