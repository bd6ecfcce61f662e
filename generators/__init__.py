"""thinfilm.generators"""
