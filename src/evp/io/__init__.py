"""Adapters between files and EVP's records: dataset readers and trajectory files."""
