# Test support: helpers, daemon harnesses and rigs for the tests (conftest.py keeps fixtures).
