"""Bringup of the whole abp graph: parameters, launch file, Recognize client, bags
(record and replay). The graph benchmark lives in abp_bench."""
