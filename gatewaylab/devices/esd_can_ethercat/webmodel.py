"""The gateway's side of the web interface (manual chapter 6): :class:`EsdWebModel` implements
:class:`~.web.EsdWebBackend` from the device's state. The web server calls it inside the clock's
lock, so it reads protocol state directly."""

from __future__ import annotations

from gatewaylab.bus.controller import ErrorState
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway
from gatewaylab.devices.esd_can_ethercat.objects import BOOTLOADER_VERSION, HARDWARE_VERSION, PRODUCT_NAME
from gatewaylab.devices.esd_can_ethercat.web import CanStatusView, DeviceInfoView

__all__ = ["EsdWebModel"]


#: esd NTCAN bus states as the status byte shows them (Figure 41 "Status: 00").
_STATUS = {ErrorState.ERROR_ACTIVE: 0x00, ErrorState.ERROR_PASSIVE: 0x80, ErrorState.BUS_OFF: 0xC0}
_WARN = 0x40


class EsdWebModel:
    """Views of one :class:`EsdGateway` for the pages of chapter 6, and its update/reboot actions."""

    def __init__(self, gateway: EsdGateway) -> None:
        self.gateway = gateway

    def info(self) -> DeviceInfoView:
        """6.1.1 Overview / Information: identity (5.1.3.5) and EtherCAT state."""
        g = self.gateway
        d = g.slave.desc
        timing = g.actual_timing()
        return DeviceInfoView(
            product=PRODUCT_NAME, serial=f"{g.serial}", hardware=HARDWARE_VERSION, firmware=g.firmware_version,
            bootloader=BOOTLOADER_VERSION, vendor_id=f"0x{d.vendor_id:08X}", product_code=f"0x{d.product_code:08X}",
            revision=f"0x{d.revision:08X}", ethercat_state=g.slave.state.name,
            station_address=g.slave.esc.station_address,
            extra={"CAN bit rate": f"{timing.bitrate} bit/s" if timing else "none",
                   "Identifier mode": "29-bit" if g.extended else "11-bit",
                   "Rx / Tx queue size": f"{g.rx_queue_size} / {g.tx_queue_size}",
                   "Local Rx / Tx queue size": f"{g.local_rx_size} / {g.local_tx_size}"})

    def can_status(self) -> CanStatusView:
        """6.2.1 Figure 41: the bit rate as set and as the controller runs it, frame statistics."""
        g = self.gateway
        st = g.stats
        ctrl = g.controller
        timing = g.actual_timing()
        status = 0
        tec = rec = 0
        if ctrl is not None:
            tec, rec = ctrl.tec, ctrl.rec
            status = _STATUS[ctrl.state]
            if status == 0 and (tec >= 96 or rec >= 96):
                status = _WARN
        requested = g.setting.requested or (timing.bitrate if timing else 0)
        deviation = 100.0 * (timing.bitrate - requested) / requested if timing and requested else 0.0
        return CanStatusView(
            bitrate_set=f"0x{g.setting.value:08x}", bitrate_actual=timing.bitrate if timing else 0,
            time_quanta=timing.time_quanta if timing else 0,
            sample_point=timing.sample_point if timing else 0.0,
            rx_std_data=st.rx.std, rx_std_rtr=st.rx.std_rtr, rx_ext_data=st.rx.ext, rx_ext_rtr=st.rx.ext_rtr,
            tx_std_data=st.tx.std, tx_std_rtr=st.tx.std_rtr, tx_ext_data=st.tx.ext, tx_ext_rtr=st.tx.ext_rtr,
            rx_bytes=st.rx_bytes, tx_bytes=st.tx_bytes, overruns=0, error_frames=st.error_frames,
            aborted_frames=st.aborted, rx_error_counter=min(rec, 255), tx_error_counter=min(tec, 255),
            status=f"{status:02X}", fifo_overruns=st.fifo_overrun, deviation=deviation, rx_bits=st.rx_bits,
            timestamp=int(g.clock.now() * 500_000))

    def start_firmware_update(self, filename: str, data: bytes) -> None:
        """6.1.2: an uploaded file starts the update (ValueError when one runs or the file is empty)."""
        self.gateway.start_update(data)

    def update_progress(self) -> str | None:
        """Figure 39's text so far, None when no update runs."""
        return self.gateway.update_progress()

    def reboot(self) -> None:
        """6.1.3 'Reboot now'."""
        self.gateway.reboot()
