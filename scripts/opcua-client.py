#!/usr/bin/env python3
"""A plant's view of the appliance over OPC UA, with Python's asyncua (pip install asyncua):
browse to the camera's vision system, read its state, subscribe to ResultReady, start one job
and print the parts of its result.

    scripts/opcua-client.py [--url opc.tcp://127.0.0.1:4840/] [--camera sim]
                            [--user NAME --password-file FILE] [--meas-id M-1 --part-id P-1]

Without a user it only reads the state (anonymous sessions may not call methods)."""
import argparse
import asyncio
import json

from asyncua import Client, ua

MV = "http://opcfoundation.org/UA/MachineVision"
DI = "http://opcfoundation.org/UA/DI/"
OWN = "urn:lfi-bridge:vision"


async def main(a):
    client = Client(a.url)
    if a.user:
        client.set_user(a.user)
        client.set_password(open(a.password_file).read().splitlines()[0])
    async with client:
        mv = await client.get_namespace_index(MV)
        # MachineVision 1.0 defines its own TrimmedString (a String); asyncua keeps that name
        # for OPC UA 1.05's and would not know this one.
        ua.uatypes.basetype_by_datatype[ua.NodeId(3017, mv)] = "String"
        await client.load_data_type_definitions()
        di, own = await client.get_namespace_index(DI), await client.get_namespace_index(OWN)
        system = await client.nodes.objects.get_child([f"{di}:DeviceSet", f"{own}:{a.camera}"])
        machine = await system.get_child([f"{mv}:VisionStateMachine"])
        auto = await machine.get_child([f"{mv}:AutomaticModeStateMachine"])
        state = (await (await machine.get_child(["0:CurrentState"])).read_value()).Text
        mode = (await (await auto.get_child(["0:CurrentState"])).read_value()).Text
        print(f"{a.camera}: {state} {mode}".strip())
        if not a.user:
            return

        events = asyncio.Queue()

        class Handler:
            def event_notification(self, event):
                events.put_nowait(event)

        subscription = await client.create_subscription(50, Handler())
        # Events of ResultReadyEventType by OfType (the server's filter does not compare node
        # ids in asyncua's default InList clause).
        result_ready = client.get_node(ua.NodeId(1024, mv))
        from asyncua.common.events import get_filter_from_event_type
        event_filter = await get_filter_from_event_type([result_ready])
        of_type = ua.ContentFilterElement(
            FilterOperator=ua.FilterOperator.OfType,
            FilterOperands=[ua.LiteralOperand(Value=ua.Variant(result_ready.nodeid))],
        )
        event_filter.WhereClause = ua.ContentFilter(Elements=[of_type])
        await subscription.subscribe_events(system, result_ready, evfilter=event_filter)

        job_id, _ = await auto.call_method(
            f"{mv}:StartSingleJob",
            ua.MeasIdDataType(Id=a.meas_id),
            ua.PartIdDataType(Id=a.part_id),
            ua.RecipeIdExternalDataType(Id=""),  # empty: the job in force
            ua.ProductIdDataType(Id=""),
            ua.Variant([], ua.VariantType.ExtensionObject),
        )
        print(f"StartSingleJob -> JobId {job_id.Id}")
        while True:
            event = await asyncio.wait_for(events.get(), 10)
            if event.JobId.Id == job_id.Id:
                break
        print(f"ResultReady {event.ResultId.Id}: MeasId {event.MeasId.Id}, ResultState {event.ResultState}")
        for part in event.ResultContent:
            print(json.dumps(json.loads(part)))

        # The same result by query (the camera keeps its newest, [opcua] results_kept).
        results = await system.get_child([f"{mv}:ResultManagement"])
        _, result, _ = await results.call_method(f"{mv}:GetResultById", ua.ResultIdDataType(Id=job_id.Id), ua.Int32(0))
        # ResultDataType's content is BaseDataType[]: each String comes inside a Variant.
        same = [v.Value for v in result.ResultContent] == list(event.ResultContent)
        print(f"GetResultById {result.ResultId.Id}: {len(result.ResultContent)} part(s), as the event: {same}")
        complete, count, _, listed, _ = await results.call_method(
            f"{mv}:GetResultListFiltered",
            ua.Int32(0),  # any ResultState
            ua.MeasIdDataType(Id=a.meas_id),
            *[t(Id="") for t in (ua.PartIdDataType, ua.RecipeIdExternalDataType, ua.RecipeIdInternalDataType,
                                 ua.ConfigurationIdDataType, ua.ConfigurationIdDataType, ua.ProductIdDataType, ua.JobIdDataType)],
            ua.UInt32(10), ua.UInt32(0), ua.Int32(0),  # MaxResults, StartIndex, Timeout
        )
        print(f"GetResultListFiltered MeasId {a.meas_id}: {count} result(s), newest {listed[0].ResultId.Id if listed else None}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", default="opc.tcp://127.0.0.1:4840/")
    p.add_argument("--camera", default="sim")
    p.add_argument("--user")
    p.add_argument("--password-file")
    p.add_argument("--meas-id", default="M-1")
    p.add_argument("--part-id", default="P-1")
    asyncio.run(main(p.parse_args()))
