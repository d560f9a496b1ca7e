# SPDX-License-Identifier: Apache-2.0
"""The ``align`` scenario of ``bringup``: align, hold, switch off and on (sample time)."""

from fiber_align.nodes.bringup import summary as sm
from fiber_align.nodes.bringup.observer import BringupError


def run_align(b):
    """
    Align, hold, run ``b.cycles`` switch cycles; return the events (sample indices).

    Waits count samples (sample time), each bounded in wall time.

    :param b: the running :class:`~fiber_align.nodes.bringup.run.Bringup`.
    :raises BringupError: a refused call, a FAULT, a timeout.
    """
    from std_srvs.srv import SetBool, Trigger
    r = b.runner

    def k(seconds):
        return int(round(seconds * b.rate))

    wall = 30.0 + 40.0 * (sm.ALIGN_MAX_S + b.cycles * (sm.SWITCH_OFF_S + sm.SWITCH_ON_S))
    r.wait_samples(k(sm.ALIGN_IDLE_S), wall, b._alive)
    events = {}
    n = len(r.states)
    res = r.call(r.align_cli, Trigger.Request(), 10.0)
    events['align'] = r.event(n)
    if not res.success:
        raise BringupError('align refused: %s' % res.message)

    def settled():
        return r.state().get('state') in ('TRACKING', 'FAULT')
    r.wait_samples(events['align'] + k(sm.ALIGN_MAX_S), wall, b._alive, settled)
    st = r.state()
    if st.get('state') != 'TRACKING':
        b.summary['align_events'] = events
        raise BringupError('alignment ended in %s: %s'
                           % (st.get('state'), st.get('fault_reason') or 'timeout'))
    events['tracking'] = _state_sample(r, 'TRACKING', events['align'])
    r.wait_samples(events['tracking'] + k(sm.LOSS_WINDOW_S), wall, b._alive)
    cyc = []
    for _ in range(b.cycles):
        n = len(r.states)
        res = r.call(r.switch_cli, SetBool.Request(data=False), 10.0)
        k_off = r.event(n)
        if not res.success:
            raise BringupError('switch off refused: %s' % res.message)
        r.wait_samples(k_off + k(sm.SWITCH_OFF_S), wall, b._alive)
        n = len(r.states)
        res = r.call(r.switch_cli, SetBool.Request(data=True), 10.0)
        k_on = r.event(n)
        if not res.success:
            raise BringupError('switch on refused: %s' % res.message)
        r.wait_samples(k_on + k(sm.SWITCH_ON_S), wall, b._alive)
        cyc.append((k_off, k_on, r.samples))
        if r.state().get('state') == 'FAULT':
            break
    events['cycles'] = cyc
    if r.state().get('state') != 'TRACKING':
        st = r.state()
        b.summary['align_events'] = events
        raise BringupError('switch cycles ended in %s: %s'
                           % (st.get('state'), st.get('fault_reason')))
    return events


def _state_sample(r, state, after):
    with r.lock:
        for k, st in r.states:
            if st.get('state') == state and k >= after:
                return k
    return r.samples
