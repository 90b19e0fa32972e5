"""Rigid-body and similarity transforms shared by every part of EVP."""
