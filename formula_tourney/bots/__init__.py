"""Bots: the follower (our "Tita") on any line, as a baseline, a demonstrator, traffic and a racer.

``follower`` drives a line with a speed profile and a steering controller; ``line_offsets`` adds
the lines that need a driver (recorded, genetic) to ``lines.registry``; ``baselines`` gives the
bot laps every table is read against; ``race_bot`` is the follower as one car among others and
``traffic_env`` one learning car among follower bots.
"""
