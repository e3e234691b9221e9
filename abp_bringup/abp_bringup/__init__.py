"""Bringup of the whole abp graph: parameters, launch file, Recognize client, bags."""
