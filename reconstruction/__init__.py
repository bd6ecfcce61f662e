"""thinfilm.reconstruction"""
