"""`armbridge report RUN.rrd`: a picture and the numbers of a run, made from its recording alone
(data.py reads it, numbers.py counts, figure.py draws with matplotlib, page.py writes the HTML)."""
