"""Code the bench scripts share, kept out of the scripts so that no script imports another."""
