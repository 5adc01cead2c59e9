"""Memristor device and crossbar array physics."""
