"""Write the Foxglove layout of the live view (docs/foxglove/seft_live_layout.json).

Run: ``.venv/bin/python tools/gen_live_layout.py`` (the docs ship its output; a test checks
that every plotted path is a channel the live view publishes for the study's run). Built
with the layout types of the foxglove-sdk package (``foxglove.layouts``): the panels of the
web page (force, displacement, acceleration with the analytical reference, valve command,
loop latency) plus the run's state and the events' log.
"""

from pathlib import Path
import sys

import foxglove.layouts as fl

OUT = Path(__file__).resolve().parents[1] / 'docs' / 'foxglove' / 'seft_live_layout.json'

M = '/seft/live/measurement'
A = '/seft/live/analytical'


def plot(title: str, series, y_label: str) -> fl.PlotPanel:
    paths = [fl.PlotSeries(value=value, label=label, color=color,
                           line_style='dashed' if dashed else 'solid')
             for value, label, color, dashed in series]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(
        paths=paths, show_legend=True, legend_display='top', y_axis_label=y_label,
        time_window_mode='automatic', is_synced=True))


def layout() -> fl.Layout:
    """The live view's panels."""
    force = plot('Force', [
        ('/seft/live/reference_force.reference_force_N', 'reference f_r', '#fbbf24', False),
        (f'{M}.measured_force_N', 'measured f_m', '#60a5fa', False),
        (f'{A}.force_N', 'analytical', '#e5e7eb', True)], 'N')
    displacement = plot('Displacement', [
        (f'{M}.displacement_m', 'test', '#60a5fa', False),
        (f'{A}.displacement_m', 'analytical', '#e5e7eb', True)], 'm')
    acceleration = plot('Acceleration', [
        (f'{M}.acceleration_m_s2', 'test', '#60a5fa', False),
        (f'{A}.acceleration_m_s2', 'analytical', '#e5e7eb', True)], 'm/s²')
    valve = plot('Valve command', [
        ('/seft/live/valve_command.valve_command_V', 'u', '#fbbf24', False)], 'V')
    timing = plot('Loop latency and missed deadlines (real time)', [
        ('/seft/live/timing/rig.loop_latency_s', 'loop latency [s]', '#60a5fa', False),
        ('/seft/live/timing/rig.loop_latency_max_s', 'max since last sample [s]', '#f472b6',
         False)], 's')
    state = fl.RawMessagesPanel(title='Run state', config=fl.RawMessagesConfig(
        topic_path='/seft/live/run', font_size=14))
    events = fl.LogPanel(title='Events', config=fl.LogConfig(
        topic_to_render='/seft/live/events', show_name=True))

    def column(*panels):
        return fl.SplitContainer(direction='column',
                                 items=[fl.SplitItem(content=p) for p in panels])
    return fl.Layout(content=fl.SplitContainer(direction='row', items=[
        fl.SplitItem(proportion=2, content=column(force, displacement, acceleration)),
        fl.SplitItem(proportion=1, content=column(valve, timing, state, events))]))


def main() -> int:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    import json
    doc = json.loads(layout().to_json())
    OUT.write_text(json.dumps(doc, indent=1) + '\n')
    print(OUT)
    return 0


if __name__ == '__main__':
    sys.exit(main())
