"""Assigning targets by auction, with bids over unicast messages.

The auctioneer is the UAV with the lowest id. Every UAV sends it (unicast) its bid: its
distance to each target. Once it holds a bid from every member (or ``wait_s`` after the first),
it awards the targets greedily, cheapest pair first, each target to one UAV and each UAV at most
one target (a sequential single-item auction, as in Koenig et al. 2006), and tells each winner
(unicast). A UAV bids again every ``rebid_s`` until it has its award (a lost message costs a
round, never a double assignment), then flies to its target.
"""

from __future__ import annotations

import math

import msgspec

from mrswarm.api import Behaviour, Context, GoTo, Hold, Intent


class AuctionParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    targets: list[tuple[float, float]]  # x, y (m, ENU) of each target
    wait_s: float = 5.0  # s the auctioneer waits for missing bids after the first one
    rebid_s: float = 1.0  # s between two bids of a UAV still without award


class Bid(msgspec.Struct, frozen=True):
    costs: list[float]  # m to each target, in the order of params.targets


class Award(msgspec.Struct, frozen=True):
    target: int  # index into params.targets


class Auction(Behaviour[AuctionParams]):
    """Bid for the targets, win one (or none), fly there."""

    Params = AuctionParams
    messages = {"auction/bid": Bid, "auction/award": Award}
    rate_hz = 5.0

    def setup(self, ctx: Context) -> None:
        self.target: int | None = None
        self.next_bid = 0.0
        self.bids: dict[int, list[float]] = {}  # the auctioneer's: uav -> its costs
        self.first_bid_at: float | None = None
        self.awarded: dict[int, int] = {}  # the auctioneer's: uav -> target

    def step(self, ctx: Context) -> Intent:
        auctioneer = min(ctx.members) if ctx.members else ctx.uav
        for m in ctx.inbox("auction/award"):
            if m.src == auctioneer and self.target is None and 0 <= m.body.target < len(self.params.targets):
                self.target = m.body.target
        if self.target is None and ctx.t >= self.next_bid:
            self.next_bid = ctx.t + self.params.rebid_s
            costs = [math.hypot(x - ctx.x, y - ctx.y) for x, y in self.params.targets]
            ctx.send_to(auctioneer, "auction/bid", Bid(costs))
        if ctx.uav == auctioneer:
            self._auctioneer(ctx)
        if self.target is None:
            return Hold()
        ctx.record("target", self.target)
        x, y = self.params.targets[self.target]
        return GoTo(x, y)

    def _auctioneer(self, ctx: Context) -> None:
        for m in ctx.inbox("auction/bid"):
            if len(m.body.costs) != len(self.params.targets):
                continue
            self.bids[m.src] = m.body.costs
            if self.first_bid_at is None:
                self.first_bid_at = ctx.t
            if m.src in self.awarded:  # its award was lost: again
                ctx.send_to(m.src, "auction/award", Award(self.awarded[m.src]))
        if self.first_bid_at is None:
            return
        everyone = all(u in self.bids for u in ctx.members)
        if not (everyone or ctx.t - self.first_bid_at >= self.params.wait_s):
            return
        taken = set(self.awarded.values())
        pairs = sorted((c, u, k) for u, costs in self.bids.items() if u not in self.awarded
                       for k, c in enumerate(costs) if k not in taken)
        for _, u, k in pairs:
            if u in self.awarded or k in taken:
                continue
            self.awarded[u] = k
            taken.add(k)
            ctx.send_to(u, "auction/award", Award(k))
